"""The encoder's rate-distortion policy: which side information to send, at which resolution, and the
check that it pays for its bytes (policy.py), over the side-information candidates it weighs (side.py)."""
