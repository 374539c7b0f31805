"""thinkfast: real-time kinodynamic belief-space planning for projectile interception."""

__version__ = "0.1.0"
