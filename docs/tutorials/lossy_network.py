# %% [markdown]
# # lossy_network
#
# (being written)
