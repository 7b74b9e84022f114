"""``wfviz run DATASET``: every clip of a folder or a list file tracked (and, with truth, scored
and explained) in local processes or on Ray, resumable, one row per clip."""
