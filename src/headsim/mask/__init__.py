"""Mask fit: seal, leak paths, contact pressure and least sealing strap force (app layer)."""
