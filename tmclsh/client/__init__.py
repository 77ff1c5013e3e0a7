"""One module on one link: requests, retries and the lock (``core``) and the components the
client owns (who watches the line and its events, ``taps``; answers in doubt, ``doubt`` on
the ``ledger``; addresses two modules answer at, ``shared``; the link reopened, switched or
closed, ``lifecycle``), the module's ASCII mode (``ascii``), and from settings to a client
brought up (``connect``)."""

# ``tmclsh.client`` was one module before the layers; scripts imported these from it
_MOVED = {"Client": ("tmclsh.client.text", "LineClient"),
          "Result": ("tmclsh.client.text", "Result"),
          "idempotent": ("tmclsh.client.core", "idempotent")}


def __getattr__(name: str) -> object:
    """An old name of ``tmclsh.client``, from its new place, with a warning naming it."""
    where = _MOVED.get(name)
    if where is None:
        raise AttributeError(f"module 'tmclsh.client' has no attribute {name!r}")
    import importlib
    import warnings

    new = f"{where[0]}.{where[1]}"
    warnings.warn(f"tmclsh.client.{name} has moved to {new} (and is tmclsh.{where[1]} if it "
                  "is in tmclsh's API): import it from there", DeprecationWarning, stacklevel=2)
    return getattr(importlib.import_module(where[0]), where[1])
