"""gnomon: attitude determination and estimation."""
__version__ = "0.1.0"
