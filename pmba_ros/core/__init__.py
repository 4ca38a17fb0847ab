"""The PMBA engine: geometry, problems, residuals, normal equations and solvers."""
