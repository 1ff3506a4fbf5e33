"""``python -m pbicrl.demonstrators ...``: see :mod:`pbicrl.demonstrators.cli`."""

from pbicrl.demonstrators.cli import main

raise SystemExit(main())
