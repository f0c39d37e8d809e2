"""Sessions as rosbag2 MCAP bags: write, read, recover, record, analyse, replay (design §7, §9).

May import the simulator, the message builders and mcap (``rosbag.py`` imports
mcap only); creates no node.
"""
