"""Stage 1 and the priors read off the input frames before training: one world frame for both
cameras (rig registration), smoke masks, whether a capture has smoke, and the smoke's colour."""
