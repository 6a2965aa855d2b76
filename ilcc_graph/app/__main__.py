"""``python -m ilcc_graph.app``: the ``ilcc-graph`` command line."""

import sys

from ilcc_graph.app import main

sys.exit(main())
