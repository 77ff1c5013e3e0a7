"""One module on one link: requests, retries, events and the lock (``core``), the module's
ASCII mode (``ascii``), and from settings to a client brought up (``connect``)."""
