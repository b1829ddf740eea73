"""The scene being learned: surface and smoke Gaussians, the smoke's motion, the environment
behind them, their optimiser, and how they are placed and rendered for one view."""
