"""Device emulators speaking the real wire protocols on 127.0.0.1 (XELA server, Net F/T, Allegro)."""
