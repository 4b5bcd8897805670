"""Person following: a wheeled robot follows its user among other people (seeds 001-004)."""
