"""The paper's estimators: closed-form estimates of the base model's g, τ, Δ from one experiment.

- :mod:`.meander`: open-loop square waves, eq. (2);
- :mod:`.pfeedback`: P feedback with a harmonic reference, eq. (3);
- :mod:`.relay`: relay feedback and its exact limit cycle, eq. (4);
- :mod:`.dispatch`: which experiment a record is, its estimate, and the JSON of it.

Nothing is imported here: each module is imported when used.
"""
