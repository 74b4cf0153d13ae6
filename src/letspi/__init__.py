"""letspi: safe highway trajectory planning with physics-informed LLMs (LetsPi).

Importing the package has no side effects; subpackages are imported on demand.
"""

__version__ = "0.1.0"
