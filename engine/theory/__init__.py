"""Theory of the schemes: predictions the lessons and tests compare the engine with."""
