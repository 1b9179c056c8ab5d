"""Real-time OpenGL viewer and headless renderer for splat4d models."""
