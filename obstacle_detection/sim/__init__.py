"""The scene generator: ray-cast scenes with known truth (:mod:`.scenes`) and sequences."""
