"""Water: coefficients and presets, the fast image-formation model, the veiling light (docs/water.md)."""
