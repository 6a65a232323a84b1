"""The pure core of cablebot: math, rules and motion; no I/O, no threads."""
