"""Schedule search: genetic scheduler with trajectory adaptation, and the exact CP-SAT baseline."""
