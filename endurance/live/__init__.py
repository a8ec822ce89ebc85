r"""The live page of a running endurance test (``stand test start|resume --serve``, ``stand test
watch``; docs/endurance.md, the live page).

::

    ring.py      a bounded ring of rows: the control loop puts, readers take what is new
    feed.py      the session's publisher (the loop's rows into a ring, a socket for watchers)
                 and the watcher's end of that socket
    trend.py     the end points' trends, flight by flight
    view.py      what the page shows from the journal: status, events, trends (read-only)
    operator.py  the token, and the operator's actions (pause, stop, resume) as the CLI takes them
    server.py    the HTTP server (tornado, on a thread of its own): the page, /status.json, the
                 stream (server-sent events), the actions
    viewer.py    a viewer of the stream without a browser (scripts, the benchmark, the tests)
    static/      the page, its script and style, and uPlot (vendored: the page loads nothing
                 from elsewhere)

Above the session (:mod:`endurance.run` takes a publisher and knows nothing of this package).
"""
