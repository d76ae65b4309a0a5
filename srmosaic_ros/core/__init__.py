"""Pure algorithm core: numpy, torch, OpenCV, scipy, filterpy. Never imports ROS or bag code."""
