"""The shared kernel beneath ``hal/`` and ``daemon/`` (docs/design.md, "Layers").

What both the devices and the method use, and nothing else: the error hierarchy
(``errors``), the one strict settings reader (``settings``), angles and SE(2) with
covariance (``angles``, ``se2``), the mirror and panorama geometry the simulator and the
method share (``mirror``, ``panorama``, ``sensor_settings``) and the ``Frame``/``Odometry``
types (``types``). It imports nothing of placecell's above it.
"""
