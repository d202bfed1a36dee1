"""Shared memory and the types every actor and algorithm uses.

Not to be confused with the ``../shared`` folder beside the repository, which
holds the design brief and the datasets.
"""
