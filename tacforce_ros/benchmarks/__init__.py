"""Benchmarks: commands that measure the runtime (speed, agreement, stops). The runtime never
imports them; each writes its results with their provenance (tacforce_ros.results)."""
