"""Readers and writers of data files and recordings."""
