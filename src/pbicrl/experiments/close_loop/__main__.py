"""``python -m pbicrl.experiments.close_loop`` (the documented command): runs :func:`pbicrl.cli.close_loop.main`.

A script of its own, so that the experiment module is imported once (the command line imports it) and the
library never imports its command line.
"""

import sys

from pbicrl.cli.close_loop import main

sys.exit(main())
