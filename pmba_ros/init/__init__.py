"""Global initialization of PMBA from feature tracks alone (pmba.md §3-4)."""
