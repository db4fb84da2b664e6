"""lm629-host inside other tools: the pytest plugin and the labgrid driver."""
