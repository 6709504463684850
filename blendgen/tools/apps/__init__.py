"""User applications on top of both halves: run, reproduce, dock, preview, the article's vehicle tables."""
