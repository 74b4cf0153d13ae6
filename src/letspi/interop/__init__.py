"""Exchange with other tools' formats (optional extras, imported only where used): ``commonroad``."""
