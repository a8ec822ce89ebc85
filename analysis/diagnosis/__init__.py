"""What a model misses in the data, and what it would take to find out.

- :mod:`.verdict`: :func:`~.verdict.diagnose`, its steps and its :class:`~.verdict.Diagnosis`;
- :mod:`.candidates`: the starting model plus one catalogue effect, fitted, judged, ranked;
- :mod:`.significance`: the criteria a richer model's cut of the error is judged by;
- :mod:`.observations`: the residual in plain words;
- :mod:`.timing`: timing jitter of the command steps, read from the residual;
- :mod:`.ambiguity`: what the data cannot tell apart, and the experiment that would;
- :mod:`.between_records`: a gain or a trend of its own per record (the stand changed);
- :mod:`.stepwise`: the model built up one effect at a time.

Nothing is imported here: each module is imported when used.
"""
