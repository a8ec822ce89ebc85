"""One module per ``stand`` sub-command."""
