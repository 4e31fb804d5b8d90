"""Hair fibres: properties, rods, collisions, electrostatics, reconstruction, rendering (app layer)."""
