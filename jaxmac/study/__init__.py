"""studies: sweeps' results pages and tables (``jaxmac results``, ``jaxmac table``)."""
