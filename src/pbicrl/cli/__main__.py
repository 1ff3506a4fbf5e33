"""``python -m pbicrl.cli ...`` is ``pbicrl ...``."""

from pbicrl.cli.app import main

raise SystemExit(main())
