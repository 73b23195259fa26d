"""Closed-form and frequency-domain analysis of attitude filters (one module per paper topic)."""
