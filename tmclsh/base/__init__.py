"""What every layer stands on: the error tree, users' files, the ranges of settings, the
configuration and profiles, and the packaged data cache. Nothing here knows TMCL."""
