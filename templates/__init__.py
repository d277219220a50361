"""Built-in assets: garment generators and coarse template types (:mod:`templates.garments`)."""
