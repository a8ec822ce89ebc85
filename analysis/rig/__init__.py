"""The rig: N loading channels on one structure, identified together (issue 31).

The model is the paper's as a matrix, ``dy/dt = G·w(t − τ) + Δ`` (:mod:`plant.rig`). This part
sits beside the estimators and the fit (``tests/test_layers.py``):

- :mod:`.record`, :mod:`.load`: the channels of a rig run on one time base
  (:class:`~.record.RigRecord`), from run directories, tables and campaign directories;
- :mod:`.synthetic`: rig runs with a known answer, written as the gateway writes them;
- :mod:`.steady`, :mod:`.regression`, :mod:`.delays`, :mod:`.periods`: the pieces of the G
  estimator: the steady stretches, each row's least squares with cluster-robust intervals,
  each channel's τ and transitional window, the meander periods that tell channels apart;
- :mod:`.estimate`, :mod:`.result`: G with its intervals, τ and Δ per channel, the physical
  check (:func:`~.estimate.estimate_rig`);
- :mod:`.onerun`: the same from one run of Hadamard meanders (:mod:`rig.excitation`), and its
  plan;
- :mod:`.coupling`: the other channels' part of one channel's force rate as a known input, so
  the one-channel fit and diagnosis find that channel's own effects
  (:mod:`analysis.diagnosis.rig` runs them, channel by channel, on an executor).
"""
