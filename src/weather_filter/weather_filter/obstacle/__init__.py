"""Paper 4's obstacle-vs-spray classifier: features, fast tree inference, the classifier, its training and its
augmented training data. Model history and run lists: ``models/obstacle_point_hgb_v4.md``."""
