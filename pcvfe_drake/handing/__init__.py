"""What the controller gets: per-context handing states, the visit tracker and their rules."""
