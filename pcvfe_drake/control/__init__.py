"""Control: the course and the friction-aware NMPC."""
