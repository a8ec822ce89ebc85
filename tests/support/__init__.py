"""Helpers the tests share (no tests here; pytest collects nothing below this folder).

stand              BASE (the stand's default plant values) and plant() (a PlantConfig with overrides)
records            synthetic records at the paper's excitations (meander4, relay, pfeedback) and the
                   independent simulator's data sets as records (independent_records, EQUIVALENT)
offline            run_offline(): an experiment driven against a plant with the gateway loop's timing
bus                recv_frames(): frames from a bus with a deadline
faults             the fault-injection tests' experiments, bus sniffer, capture queries, reaction log
independent_stand  an independent stand simulator (written apart from plant/ and analysis/)

Fixtures stay in tests/conftest.py. A test module imports helpers from here, never from another
test module or from conftest (tests/test_layers.py checks it)."""
