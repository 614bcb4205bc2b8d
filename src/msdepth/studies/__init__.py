"""What more than one study script (``studies/*.py``) shares: the real sample frames' camera and
scores, the studies' variant specs. The scripts import it as any other package, so the layering
test sees their edges; no script imports another."""
