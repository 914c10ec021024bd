"""Individual human models: temporal (durations) and spatial (where the person is)."""
