r"""The live page of a running endurance test (``stand test start|resume --serve``, ``stand test
watch``; docs/endurance.md, the live page).

::

    ring.py      a ring of rows in a file both processes map: the loop writes, readers copy
    feed.py      the session's publisher (the loop's rows into TESTDIR/live.ring) and the
                 server's reader of it, from session to session
    trend.py     the end points' trends, flight by flight
    view.py      what the page shows from the journal: status, events, trends (read-only)
    operator.py  the token, and the operator's actions (pause, stop, resume) as the CLI takes them
    binding.py   where the page listens, the names it answers to, its certificate
    limits.py    what a client may take, and how refusals are counted and told
    guard.py     the HTTP server below the application: connections counted and bounded
    server.py    the application: the page, /status.json, the stream (server-sent events), the
                 actions
    process.py   the server as a process of its own, and the session's watch that starts it again
    viewer.py    a viewer of the stream without a browser (scripts, the benchmark, the tests)
    static/      the page, its script and style, and uPlot (vendored: the page loads nothing
                 from elsewhere)

Above the session (:mod:`endurance.run` takes a publisher and knows nothing of this package).
"""
