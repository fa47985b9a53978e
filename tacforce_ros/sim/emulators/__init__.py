"""Device emulators speaking the real wire protocols on 127.0.0.1: xela_server, Net F/T RDT,
Allegro V4 CAN (through a socketcand server)."""
