"""Loading the structure: programmes, the controller designed from the identified model, peak/
valley compensation and the tracking report.

- :mod:`loading.programme`: loading programmes (turning points, time histories, sines, blocks);
- :mod:`loading.design`: a force controller from a fitted model (feedforward through the model's
  inverse, PI feedback with margins at the boosted gain), as a TOML file;
- :mod:`loading.controller`: the controller's law, one call per control cycle;
- :mod:`loading.compensation`: peak/valley compensation that learns across cycles and passes;
- :mod:`loading.report`: how well a pass tracked the programme (turning points, rainflow).

It uses only :mod:`core` and :mod:`plant`; the gateway's load experiment runs it on the stand.
"""
