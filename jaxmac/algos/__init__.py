"""Learners: one module each (``tomacvf`` a package), holding its settings, its scenario values, its networks'
wiring, its loss and its acting rule, on the shared trainer; ``families/`` the code several learners share;
``registry`` the list of learners (``REGISTRY``, ``make_algorithm``)."""
