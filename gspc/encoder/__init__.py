"""The encoder: every choice it makes about a scene, in one call (decisions.py), over its steps: cameras,
measure and attribute coding (prepare.py, significance.py), rate control (rate.py), the removal and position
grid chosen per scene (removal.py), the side-information candidates (side.py) and the policy that weighs them
against the same bytes on attributes (policy.py), and the tuning of the coded values (tuning.py)."""
