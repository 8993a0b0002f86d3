"""Readers and writers of each ground-truth file format, one module per format."""
