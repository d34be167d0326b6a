"""Linear policies found by search, as the random-search tutorial does: random search, hill climbing
and the cross-entropy method, one search per seed (search.py: the config, the searches, the specs),
the linear policy and how candidates play (policy.py), every seed's candidates played in one vector
env (population.py)."""
