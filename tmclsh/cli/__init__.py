"""The command line: the option parser (``options``), the entry point (``main``) and the man
page and completions generated from both (``docs``)."""
