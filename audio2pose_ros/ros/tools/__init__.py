"""Tools that test and measure the nodes, apart from the nodes and what they share.

The fault campaign (``audio2pose faults``: fault_campaign, its cases and harness), the benchmarks
(``audio2pose bench --graph`` and ``--console``: graph_bench, console_bench), the bare rclpy
floor the graph is measured against (relay_floor) and process figures read from /proc
(process_stats). No node imports them.
"""
