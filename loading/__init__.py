"""Loading the structure: programmes, the controller designed from the identified model, peak/
valley compensation and the tracking report.

- :mod:`loading.programme`: loading programmes (turning points, time histories, sines, blocks);
- :mod:`loading.design`: a force controller from a fitted model (feedforward through the model's
  inverse, PI feedback with margins at the boosted gain), as a TOML file;
- :mod:`loading.controller`: the controller's law, one call per control cycle;
- :mod:`loading.compensation`: peak/valley compensation that learns across cycles and passes;
- :mod:`loading.report`: how well a pass tracked the programme (turning points, rainflow);
- :mod:`loading.minimum_time`: a programme's valve-limited minimum time;
- :mod:`loading.pacing`: null pacing, the programme's clock that waits or slows for the force;
- :mod:`loading.time_scaling`: segment durations scaled pass by pass to the accuracy; schedules;
- :mod:`loading.gain_monitor`: the stand's g re-estimated block by block, followed, watched;
- :mod:`loading.load_page`: the page of a loading test (``stand report LOAD_DIR``).

It uses only :mod:`core` and :mod:`plant`; the gateway's load experiment runs it on the stand.
"""
