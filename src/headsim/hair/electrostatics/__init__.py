"""Electrostatic charging of hair (Sobottka 2008, ch. 4)."""
