"""The camera sensor: EMVA 1288 photon transfer, exposure, distortion, 8-bit encoding (docs/sensor.md)."""
