"""studies: sweeps' results pages and tables (``jaxmac results``, ``jaxmac table``), measured rates of sweep cells
(``jaxmac calibrate``), curves of several runs on one figure (``jaxmac overlay``)."""
