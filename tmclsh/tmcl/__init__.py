"""The TMCL protocol as data and pure code, no I/O: frames and status codes, the one frame
decoder, the version decoder, the ASCII line codec, the instruction set, the module database
and the assembler. Everything above reads its facts from here."""
