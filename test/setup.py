"""System tests of rths (a colcon package so that `colcon test` runs them)."""

from setuptools import setup

package_name = 'rths_system_tests'

setup(
    name=package_name,
    version='0.1.0',
    packages=['rths_system_tests'],
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='rths maintainers',
    maintainer_email='maintainers@rths.dev',
    description='System tests of rths.',
    license='Apache-2.0',
    tests_require=['pytest'],
)
