"""One walk through the filter (the pipeline: causal rows as records arrive, the offline track at
the end) and radio maps grown from tracked walks."""
