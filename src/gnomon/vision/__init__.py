"""Vision aiding for attitude (seed 003): pinhole camera, rendered/warped real imagery,
the one-parameter strip matcher and the gyro-only SINS it corrects.

Camera frame = body frame (the camera's optical axis is the vehicle's longitudinal
axis): x forward (optical axis), y right (image columns grow), z down (image rows
grow). Navigation frame n: North-East-Down; ``R_nb = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.
Nothing here is imported by ``import gnomon``.
"""
