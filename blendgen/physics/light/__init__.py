"""Light sources in water: point lights, the dock's LEDs, the vehicle's lamps, light on surfaces (docs/light.md)."""
