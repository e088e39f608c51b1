"""The droplet reference (real-size drops, per-beam detection) and the metrics that compare the
spray model's clouds with it (BEV histograms, Pearson, Jaccard, Hamming)."""
