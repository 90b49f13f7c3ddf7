# %% [markdown]
# # own_system
#
# (being written)
