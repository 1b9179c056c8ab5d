"""Training of native 4D Gaussians: rasterizer, datasets, losses, recipes."""
