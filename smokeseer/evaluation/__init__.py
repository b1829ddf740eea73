"""After training: scores on the held-out views, renders, PLY exports and one figure per test view."""
