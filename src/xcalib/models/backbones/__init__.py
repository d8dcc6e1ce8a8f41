"""Backbones written here (no torchvision): tiny ResNets, ViT, PointNet, PointNet++, GNN."""

from .gnn import EdgeAwareGAT, StructureGNN, knn_edges
from .pointnet import PointNetEmbedding, TinyPointNet
from .pointnet2 import PointNet2SSG
from .resnet import BottleneckResNet, ResNetEmbeddingDeep, SmallCNN
from .vit import CropViT

__all__ = ["EdgeAwareGAT", "StructureGNN", "knn_edges", "PointNetEmbedding", "TinyPointNet", "PointNet2SSG",
           "BottleneckResNet", "ResNetEmbeddingDeep", "SmallCNN", "CropViT"]
