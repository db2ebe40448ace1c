"""doodlecam studio: the job in the browser (docs/studio.md). Imported only by ``doodlecam studio``."""
