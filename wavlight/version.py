"""The version of wavlight, recorded in experiment results and bake files."""
__version__ = "0.1.0"
