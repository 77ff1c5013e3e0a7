"""What is done to a module, usable from Python and never printing: stored programs, the
safety stop, scanning a line or bus. Results come back as data; the shell renders them."""
