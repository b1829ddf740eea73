"""Stages 2 and 3: the shared training loop, the losses and Stage 3's priors (depth, mask
floor), the validation split, and the run log and checkpoints."""
