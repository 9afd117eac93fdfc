"""The Awiwi hand: fingers (thesis ch. 5) and wrist (ch. 6)."""
