"""Imported first by the workers' fork server (``workers.PRELOAD``), and by no other process.

The server loads the per-frame stages once (about a second) before it ignores SIGINT itself; a
terminal's Ctrl-C in that second reaches the whole process group and would end the server with a
traceback. Its workers inherit the setting (the main process decides when they end).
"""

import signal

signal.signal(signal.SIGINT, signal.SIG_IGN)
