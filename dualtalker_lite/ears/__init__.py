"""Our own ears: a causal viseme recogniser distilled from the offline track (issue 47)."""
