"""Fat-grafting planner: volume injection into a marked face region by PBD (app layer)."""
