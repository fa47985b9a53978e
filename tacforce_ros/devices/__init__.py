"""Device wire protocols and their clients (no ROS): ``xela`` (xela_server WebSocket),
``netft`` (ATI Net F/T RDT over UDP), ``allegro`` (Allegro V4 over python-can). Every driver is
a ``polling.PollingDriver`` (poll() or start(), callbacks, latest(), is_stale(), close()) with
``diagnostics.LinkDiagnostics`` counters."""
