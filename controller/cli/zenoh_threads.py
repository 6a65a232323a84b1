"""Threads of a client verb that call Zenoh (a status poller, a command sent beside a
dashboard).

Such a thread is never a daemon thread. Zenoh runs a Python callback (of a subscriber, or of
a query's replies) on a Python thread of its own, started by the thread that declared it and
so a daemon thread when that one is; and a thread that waits inside Zenoh's native code gives
up the interpreter while it waits. A daemon thread still in there when the interpreter exits
is torn down by `pthread_exit` from inside that native code as it wakes (a reply arriving, the
session closing), which aborts the whole process with glibc's "FATAL: exception not
rethrown", after the verb has done its work and printed its last line. The interpreter waits
at exit for a thread that is not a daemon, and these end within a query's timeout of their
stop (at once when the session closes).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any


def start_zenoh_thread(target: Callable[..., Any], *args: Any, name: str) -> threading.Thread:
    """Start `target(*args)` on a thread named `name` that may call Zenoh: not a daemon
    thread, whatever the thread that starts it (module docstring). The caller stops it (an
    event `target` watches) and may join it; the interpreter joins it at exit in any case.
    Raises what `threading.Thread.start` raises."""
    thread = threading.Thread(target=target, args=args, name=name, daemon=False)
    thread.start()
    return thread
