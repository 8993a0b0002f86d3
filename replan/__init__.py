"""replan stage."""
