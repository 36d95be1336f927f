"""Allow ``python -m virtualgps``."""

from virtualgps.cli import main

raise SystemExit(main())
