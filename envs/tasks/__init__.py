"""Tasks: goals, reward terms, success and termination, one module per env."""
