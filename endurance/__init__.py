"""The endurance test: a flight-by-flight fatigue test run for months, and what watches it."""
