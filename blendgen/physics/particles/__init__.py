"""Small obstacles and marine snow: the field, its optics, the compiled splat (docs/particles.md)."""
