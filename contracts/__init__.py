"""What the generator, the trainer and the harness share: the dataset format and its reader,
the results format, the metrics, atomic writes and provenance. It imports none of them."""
