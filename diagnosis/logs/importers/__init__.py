"""File formats read into :class:`~realitygap.diagnosis.logs.log.Log`: OptiOdom sessions, CSV with a
column map, ROS 1/2 bags, UR10 laser-tracker series, FR3 eye-in-hand archives, and the
safe reading of saved archives."""
