from .base import startup

startup.hold()  # (from the first import on: base/startup.py; cli.main's main lets it go)

from .cli.main import main  # noqa: E402

raise SystemExit(main())
