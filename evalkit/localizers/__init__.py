"""Built-in marker localizers of evalkit.

Each is a class with ``reset(camera: dict)`` (once per sequence) and
``localize(image: HxWx3 uint8 RGB) -> dict | None``; see datasets_spec/LOCALIZER_PROTOCOL.md and the README's
"Writing a localizer". The class
attribute ``outputs`` lists the result fields it fills: ``distance`` (m), ``T_cam_dock``
(full 6-DoF pose) and ``marker_id`` (the identity-checked marker that produced it).
- ``evalkit.localizers.led:LedLocalizer``     N >= 4 LEDs, reference LED(s) by colour, IPPE PnP
  (blob stage: ``led_blobs``)
- ``evalkit.localizers.qr:QrLocalizer``       QR code (zxing-cpp by default), payload-checked, ECC-aligned corners
- ``evalkit.localizers.aruco:ArucoLocalizer`` ArUco / AprilTag (OpenCV dictionaries), IPPE_SQUARE
- ``evalkit.localizers.apriltag:AprilTagLocalizer`` AprilTag with pupil-apriltags
- ``evalkit.localizers.hybrid:HybridLocalizer`` QR or LED per frame, by predicted range error
Shared code: ``pnp`` (planar PnP + disambiguation), ``square`` (the square-marker base
class: marker pick, grey image, ``detect`` hook, ROI search, best pose).
"""
