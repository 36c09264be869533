"""``avgs bench``: latency, speed against error, training throughput; writes benchmarks/REPORT.md."""
