"""Built-in marker localizers of evalkit.

Each is a class with ``reset(camera: dict)`` (once per sequence) and
``localize(image: HxWx3 uint8 RGB) -> dict | None``; see SPEC.md section 7.
- ``evalkit.localizers.led:LedLocalizer``     4-LED array, reference LED by colour, IPPE PnP
- ``evalkit.localizers.qr:QrLocalizer``       QR code, payload-checked, finder-corner PnP
- ``evalkit.localizers.aruco:ArucoLocalizer`` ArUco / AprilTag (OpenCV dictionaries), IPPE_SQUARE
Shared code: ``pnp`` (planar PnP + disambiguation), ``square`` (square markers).
"""
