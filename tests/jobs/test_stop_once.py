"""A link process's stop handler under two stop signals (the group's SIGTERM and `fabline run`'s SIGINT): the second,
run inside the first while the first holds the abort event's lock, must not wait on that lock (it hung a link process
after its abort line). Truth: a real threading.Event whose set() the nested handler would re-enter."""

import threading

from fabline.jobs.streaming import StopOnce


def test_a_second_stop_inside_the_first_returns_at_once():
    aborting = threading.Event()
    calls = []

    def stop():
        calls.append("stop")
        with aborting._cond:      # where the first handler was when the second signal came: inside Event.set
            handler()             # the second signal's handler runs here, in the same thread
            aborting._flag = True
            aborting._cond.notify_all()

    handler = StopOnce(stop)
    worker = threading.Thread(target=handler, daemon=True)
    worker.start()
    worker.join(5)
    assert not worker.is_alive(), "the nested stop waited on the abort event's lock"
    assert calls == ["stop"] and aborting.is_set()
