"""The real benchmark records: runs, standard protocols with baselines, dataset slices, documented report figures."""
