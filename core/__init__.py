"""What every layer shares and nothing else: the errors a user can act on (:mod:`core.errors`)."""
