"""Our own ears (issue 47): a causal viseme recogniser (the *student*, ``model``) distilled from the offline
recogniser's track (the *teacher*) by ``distil``, on training audio from registry packages. docs/ears.md."""
