"""ROS 2 over Zenoh without a bridge: rmw_zenoh's wire format (pure modules) and the node."""
