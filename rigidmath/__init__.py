"""Plain-numpy rigid-body math shared by the scenes and the simulator: mass properties of
particle clusters and unit quaternions. It imports no engine and compiles nothing."""
