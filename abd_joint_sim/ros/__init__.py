"""ROS 2 front end of abd_joint_sim: the sim_node executable and its plain-Python helpers.

Only this subpackage and ``abd_joint_sim.record`` import rclpy; the physics core never does.
"""
