"""Other feature-learning objectives behind the same interface as TRASE's."""
