"""The endurance test: a flight-by-flight fatigue test of many flights, unattended for months,
on a station of N channels (a stand is N = 1), and what watches it (docs/endurance.md).

``testfile``  the test file (test.toml): station, controller, flight types, block, target,
              inspections, monitors, storage; its fingerprint
``spectrum``  the block and the flight sequence: flight n -> block, position, type
``journal``   the journal (SQLite): the count, the flight and load case in progress, events,
              what was learnt per flight type, the end points; the test directory's lock
``storage``   the turning-point log (Parquet by block), the rolling window of full-rate
              signals and the event windows (run directories), the storage estimate
``trends``    the end-point trends: a crack at an attachment seen from the flows the valves
              need to reach their end points, flight by flight
"""
