"""What the rclpy under test gives, for tests whose expectations differ between distros.

``PUBLISHER_GIDS``: message infos carry the publisher's gid (Kilted's rclpy and later; the
same release brought ``rclpy.subscription.MessageInfo``). Jazzy's and Humble's do not, so the
nodes cannot tell two publishers of one topic apart by their messages there.
"""

import rclpy.subscription

PUBLISHER_GIDS = hasattr(rclpy.subscription, "MessageInfo")
