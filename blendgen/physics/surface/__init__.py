"""The water surface seen from below and the caustics its waves focus (docs/light.md)."""
