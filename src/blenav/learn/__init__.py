"""Learned localization (Roy, chapter 3): data windows, networks, training. Grows with issues 4 and 5."""
