"""The encoder beyond the attribute codec: its stages before the policy (stages.py: cameras, attribute
coding, the side-information views), the side-information candidates (side.py) and the rate-distortion
policy that weighs them (policy.py: which side information to send, at which resolution, and the check that
it pays for its bytes)."""
