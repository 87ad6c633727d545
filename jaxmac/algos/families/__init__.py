"""What several learners of one family share: the joint-Q pieces (``centralised``: Mac-Cen-DDRQN, Mac-Dec-MADDRQN,
Mac-CAC, Mac-NIACC's joint inputs), the per-agent DRQN pieces (``decentralised``: MacDec-Q, Mac-Dec-MADDRQN, AVF) and
the macro-action actor-critics' pieces (``actor_critic``: Mac-IAICC, Mac-NIACC, Mac-CAC). A learner imports these,
never another learner."""
